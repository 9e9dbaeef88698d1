"""`python -m prompose_grasp.cli`: the `prompose-grasp` command."""

import sys

from prompose_grasp.cli import main

sys.exit(main())
