import sys

from hil.cli import entry

sys.exit(entry())
