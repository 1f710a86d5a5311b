"""``python -m multirotor_ros.cli``: the same as the ``multirotor`` command."""

import sys

from multirotor_ros.cli import main

# The guard matters: the command discovery in cli/__init__.py imports every module of this package,
# this one included, and must not run the command line when it does.
if __name__ == "__main__":
    sys.exit(main())
