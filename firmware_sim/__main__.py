"""``python -m firmware_sim`` is ``firmware-sim``."""

import sys

from .cli import main

sys.exit(main())
