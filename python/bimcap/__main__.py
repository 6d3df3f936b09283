import sys

from bimcap.cli import main

sys.exit(main())
