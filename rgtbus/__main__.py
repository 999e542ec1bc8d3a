import sys

from rgtbus.cli import main

sys.exit(main())
