"""`python -m headctl`: the same as the `headctl` command."""
import sys

from headctl.cli.main import main

sys.exit(main())
