"""``python -m world --config world.json``: the world service (world/service.py)."""

import sys

from world.service import main

sys.exit(main())
