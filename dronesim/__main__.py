import sys

from dronesim.cli import main

sys.exit(main())
