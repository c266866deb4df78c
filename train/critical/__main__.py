"""``python -m train.critical generate-data | train | evaluate [flags]``."""

import sys

from train.critical.cli import main

sys.exit(main())
