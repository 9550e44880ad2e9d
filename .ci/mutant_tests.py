"""Run the given pytest selections for one mutant (`.ci/mutation`): exit 1 when
any test fails, errors or times out (killed), 0 when all pass (survived).

mutmut 2 counts only exit status 1 as killed; pytest's 2-5 (a collection error
from a mutant that breaks an import, an interruption) are mapped to 1 here.
"""

from __future__ import annotations

import subprocess
import sys

args = [sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", "--no-header", *sys.argv[1:]]
try:
    rc = subprocess.run(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, timeout=300).returncode
except subprocess.TimeoutExpired:
    rc = 1
sys.exit(0 if rc == 0 else 1)
