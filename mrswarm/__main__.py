import sys

from mrswarm.cli import main

sys.exit(main())
