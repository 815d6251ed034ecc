"""``python -m clutch_ros.cli`` runs the ``clutch`` command."""

import sys

from clutch_ros.cli.main import main

sys.exit(main())
