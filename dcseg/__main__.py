import sys

from dcseg.cli import main

sys.exit(main())
