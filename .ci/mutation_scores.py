"""Per-file mutation scores from mutmut 2's cache (run in the `.ci/mutation` scratch copy):
killed (failing tests, slow kills and timeouts) over killed + survived; skipped and untested
mutants are not scored."""

from __future__ import annotations

import sqlite3
from collections import Counter, defaultdict

rows = sqlite3.connect(".mutmut-cache").execute(
    "select s.filename, m.status, count(*) from Mutant m join Line l on m.line = l.id "
    "join SourceFile s on l.sourcefile = s.id group by s.filename, m.status")
by: dict[str, Counter[str]] = defaultdict(Counter)
for name, status, n in rows:
    by[name][status] += n
total = Counter[str]()
for c in by.values():
    total.update(c)
for name, c in [*sorted(by.items()), ("all", total)]:
    killed = c["ok_killed"] + c["ok_suspicious"] + c["bad_timeout"]
    score = f"{100 * killed / (killed + c['bad_survived']):.0f}%" if killed + c["bad_survived"] else "-"
    print(f"{name}: {score} ({killed} killed, {c['bad_survived']} survived, {c['skipped']} skipped, "
          f"{c['untested']} untested)")
