"""``python -m firmware_sim`` is ``firmware-sim``.

Until :func:`firmware_sim.cli.main` puts its own handlers in place (:class:`firmware_sim.cli.StopOnSignals`),
a Ctrl-C ends the process by the signal, as SIGTERM and SIGHUP do: nothing is made yet that needs cleaning
up, and Python's own handler met it with a ``KeyboardInterrupt`` traceback out of the ~0.4 s of imports.
"""

import signal
import sys

signal.signal(signal.SIGINT, signal.SIG_DFL)

from .cli import main  # noqa: E402 — after the handler above: these imports are the window it covers

sys.exit(main())
