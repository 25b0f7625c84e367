"""``python -m tympani.pipeline.cli``: the same as the ``tympani`` command."""

import sys

from tympani.pipeline.cli import main

sys.exit(main())
