"""``python -m topomatch``."""

import sys

from topomatch.cli import main

sys.exit(main())
