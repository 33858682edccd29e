import sys

from eve3d.cli import main

sys.exit(main())
