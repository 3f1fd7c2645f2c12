"""``python -m planar_vo.synth``."""

import sys

from planar_vo.synth.cli import main

sys.exit(main())
