"""``python -m econdor`` is the ``econdor`` command."""

import sys

from .cli import main

sys.exit(main())
