"""``tracker.clusters``: moving objects as clusters of events, event by event,
in the style of jAER's rectangular cluster tracker (Delbruck & Lichtsteiner,
ISCAS 2007, the robot goalie).

Every event joins the nearest cluster (L-inf distance) whose capture box
holds it, or seeds a new one. A cluster's capture box has half sides of
1.5 times the half width of a uniformly filled box with the cluster's
variance per axis, within ``radius_px .. max_radius_px``: a new cluster
captures ``radius_px`` about its seed and grows to its object (the factor
above 1 lets it grow; ``max_radius_px`` keeps two objects that met from
staying one cluster once they part). A cluster's centre moves ``mix`` of
the way to each event it takes (after moving by its velocity over the time
since its last event: ``predict``), its variances likewise; its mass is a
count of its events decaying with time constant ``tau_us``, so ``mass /
tau`` is its event rate; its velocity follows the centre's displacement,
sampled every ``velocity_us`` of its events and low-passed over
``velocity_tau_us``. At each velocity sample (and at its seed) a cluster
merges with every cluster whose centre lies within ``merge`` times the
larger of the two capture boxes into the heavier one, which keeps the older
id. A cluster is visible once its mass reaches ``min_mass`` (an event rate
of ``min_mass / tau_us``: 3,000 ev/s with the defaults) and takes the next
id then, so noise that seeds short-lived clusters takes no ids; it is
dropped when its mass decays below ``prune_mass``. At most ``max_clusters``
live at once: when full, the never-visible cluster whose last event is
oldest gives up its place. Width and height (px) are those of a uniformly
filled box with the cluster's variance per axis: the extent of an object's
events, not its outline. Choose ``radius_px`` about 1.5 times the
objects' radius and ``max_radius_px`` about twice it (the defaults suit
objects of 6-10 px radius): a cluster seeded on one edge of an object must
reach the opposite edge, whose events a realistic sensor's photoreceptor
delays by milliseconds (measured on 240x180 disks of 8 px at 300 px/s,
1 s: 12/16 px gave two clusters on one disk, 6 id switches/s, where 14/20
px gave none).

Output (:class:`~tectum.ClusterPacket`: ``t, id, x, y, vx, vy, width,
height, mass``; px, px/s, events): with ``update_us`` > 0, every visible
cluster at every multiple of ``update_us`` µs, the state after all events
up to and including that time (a row comes out when an event or the
watermark passes that time: event-to-output delay at most ``update_us`` in
stream time); with ``update_us=0``, a row per event that lands in a visible
cluster, at the event's time (the goalie's path: no delay, one row per
event). Rows of one time come by id. Either way the rows depend on the
events alone, never on how packets cut the stream.

Cost: per event one pass over the live clusters (comparisons only) and a
table lookup for the mass decay; a pass more per velocity sample (merges);
state ``max_clusters x 15`` float64. Noise seeds clusters that
never become visible; at 2 Hz/px on 346x260 that is 180,000 seeds per second
(each lives ``tau_us ln(1 / prune_mass)``), so a denoiser in front
(``filter.background_activity``) keeps the cluster slots for objects.
"""

from __future__ import annotations

import numpy as np

from tectum import ClusterPacket, EventPacket, Kind, Operator, Packet

from ._clusters import (
    C_EVICTED,
    C_MERGED,
    C_PRUNED,
    C_SEEDED,
    NPAR,
    OUT_COLS,
    P_LN_PRUNE,
    P_MAX_RADIUS,
    P_MERGE,
    P_MIN_MASS,
    P_MIX,
    P_PRUNE,
    P_RADIUS,
    P_TAU,
    P_UPDATE,
    P_VEL_DT,
    P_VEL_TAU,
    clusters_kernel,
    new_state,
)

__all__ = ["Clusters", "track_clusters"]


class Clusters(Operator):
    """Moving-object cluster tracker (see the module).

    Parameters
    ----------
    radius_px:
        Smallest half side of a cluster's capture box, px (a new cluster's).
    max_radius_px:
        Largest half side of a capture box, px.
    max_clusters:
        Live clusters at most (visible or not).
    mix:
        Fraction of the way the centre (and the variances) move towards each
        event, in (0, 1].
    tau_us:
        Mass decay time constant, µs.
    min_mass:
        Mass (decayed event count) from which a cluster is visible.
    prune_mass:
        Mass below which a cluster is dropped (< ``min_mass``).
    update_us:
        Output every this many µs; 0: a row per event in a visible cluster.
    velocity_us:
        Velocity sampled every this many µs of a cluster's events.
    velocity_tau_us:
        Velocity low-pass time constant, µs.
    merge:
        Clusters whose centres are within ``merge`` times the larger capture
        box (per axis) merge.
    predict:
        Move the centre by its velocity before mixing in an event.
    """

    name = "tracker.clusters"
    consumes = (Kind.EVENTS,)
    produces = (Kind.CLUSTERS,)

    def __init__(self, radius_px: float = 14.0, max_radius_px: float = 20.0, max_clusters: int = 16,
                 mix: float = 0.05, tau_us: int = 10_000, min_mass: float = 30.0, prune_mass: float = 0.5,
                 update_us: int = 1000, velocity_us: int = 1000, velocity_tau_us: int = 10_000, merge: float = 1.0,
                 predict: bool = True) -> None:
        if not 0 < radius_px <= max_radius_px or max_clusters < 1 or not 0 < mix <= 1 or tau_us <= 0:
            raise ValueError("need 0 < radius_px <= max_radius_px, max_clusters >= 1, 0 < mix <= 1 and tau_us > 0")
        if not 0 < prune_mass < min_mass or update_us < 0 or velocity_us < 1 or velocity_tau_us < 0 or merge < 0:
            raise ValueError("need 0 < prune_mass < min_mass, update_us >= 0, velocity_us >= 1, "
                             "velocity_tau_us >= 0 and merge >= 0")
        self.update_us = int(update_us)
        par = np.zeros(NPAR)
        par[P_RADIUS], par[P_MIX], par[P_TAU] = radius_px, mix, tau_us
        par[P_MIN_MASS], par[P_PRUNE], par[P_UPDATE] = min_mass, prune_mass, update_us
        par[P_VEL_DT], par[P_VEL_TAU], par[P_MERGE] = velocity_us, velocity_tau_us, merge
        par[P_MAX_RADIUS], par[P_LN_PRUNE] = max_radius_px, np.log(1.0 / prune_mass)
        self.par = par
        # exp(-g / tau) for gaps of g whole µs up to the time a single event's mass lasts
        self._table = np.exp(-np.arange(int(min(tau_us * np.log(min_mass / prune_mass) * 4, 1 << 16)) + 1) / tau_us)
        self.cl, self.ids, self.meta = new_state(int(max_clusters))
        self.meta[3] = int(bool(predict))
        self._counts = np.zeros(4, np.int64)
        self.counts = {"seeded": 0, "evicted": 0, "merged": 0, "pruned": 0}
        self._mark: int | None = None

    def warmup(self) -> None:
        twin = Clusters(update_us=self.update_us or 1000)
        t = np.arange(0, 4000, 10, dtype=np.int64)
        xy = (10 + (t // 100) % 5).astype(np.uint16)
        twin.process(EventPacket(t, xy, xy, np.ones(len(t), np.int8), sensor=(32, 32), t_start=0, t_end=4000))
        if self.update_us == 0:
            twin = Clusters(update_us=0)
            twin.process(EventPacket(t, xy, xy, np.ones(len(t), np.int8), sensor=(32, 32), t_start=0, t_end=4000))

    def process(self, packet: EventPacket) -> list[Packet]:
        if self._mark is None:
            self._mark = packet.t_start
        t, i, parts = packet.t, 0, []
        K = self.cl.shape[0]
        while True:
            cap = max(len(t) + K, 4 * K) if self.update_us == 0 else max(64 * K, len(t) // 8 + K)
            ot, oid, out = np.empty(cap, np.int64), np.empty(cap, np.int64), np.empty((cap, OUT_COLS))
            r, i, done = clusters_kernel(t, packet.x, packet.y, i, packet.t_end, self.cl, self.ids, self.meta,
                                         self.par, self._table, self._counts, ot, oid, out)
            if r:
                parts.append((ot[:r], oid[:r], out[:r]))
            if done:
                break
        for name, k in (("seeded", C_SEEDED), ("evicted", C_EVICTED), ("merged", C_MERGED), ("pruned", C_PRUNED)):
            self.counts[name] = int(self._counts[k])
        if not parts:
            return []
        ot, oid, out = (np.concatenate([p[j] for p in parts]) for j in range(3))
        order = np.lexsort((oid, ot))  # by time, then id (stable: a time's rows all come in one packet)
        ot, oid, out = ot[order], oid[order], out[order]
        pkt = ClusterPacket(ot, id=oid, x=out[:, 0], y=out[:, 1], vx=out[:, 2], vy=out[:, 3], width=out[:, 4],
                            height=out[:, 5], mass=out[:, 6], t_start=self._mark, t_end=packet.t_end)
        self._mark = packet.t_end
        return [pkt]


def track_clusters(events: EventPacket, **params: float | int | bool) -> ClusterPacket:
    """The function form: every cluster row of a whole event packet (the
    parameters of :class:`Clusters`)."""
    op = Clusters(**params)  # type: ignore[arg-type]
    out = op.process(events)
    if out:
        assert isinstance(out[0], ClusterPacket)
        return out[0]
    return ClusterPacket(np.empty(0, np.int64), id=np.empty(0, np.int64), x=np.empty(0), y=np.empty(0),
                         vx=np.empty(0), vy=np.empty(0), width=np.empty(0), height=np.empty(0), mass=np.empty(0),
                         t_start=events.t_start, t_end=events.t_end)
