"""``python -m hil_mock`` = ``hil-mock``."""

import sys

from hil_mock.cli import main

sys.exit(main())
