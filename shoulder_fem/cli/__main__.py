"""``python -m shoulder_fem.cli``."""

import sys

from shoulder_fem.cli.main import main

sys.exit(main())
