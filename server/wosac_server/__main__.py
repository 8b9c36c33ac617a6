import sys

from wosac_server.cli import main

sys.exit(main())
