import sys

from tectum.cli import main

sys.exit(main())
