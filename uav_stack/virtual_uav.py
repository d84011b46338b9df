"""``python -m uav_stack.virtual_uav --config FILE``: one virtual UAV process (see runtime.py)."""

import sys

from uav_stack.runtime import virtual_uav_main

if __name__ == "__main__":
    sys.exit(virtual_uav_main())
