"""The ground station: a browser page that follows a run live (downlink) and commands it (uplink), or
replays a run directory, finished, killed or still being written (docs/gcs.md).

``hil run --gcs [HOST:PORT]`` serves a live run; ``hil gcs RUN_DIR`` a run directory. In code::

    with GroundStation.live() as station:          # loopback, a fresh token
        print(station.url)
        run(scenario, RunOptions(observer=station.observer, pace=1.0))

A tool layer above :mod:`hil.runtime`: the runtime knows only its observer hook
(:mod:`hil.runtime.observer`).
"""

from hil.gcs.access import parse_bind
from hil.gcs.live import LiveFeed
from hil.gcs.rundir import RunDirSource
from hil.gcs.station import GroundStation
from hil.gcs.uplink import Uplink

__all__ = ["GroundStation", "LiveFeed", "RunDirSource", "Uplink", "parse_bind"]
