"""``python -m controltac_il.augment`` (see ``cli``)."""

import sys

from controltac_il.augment.cli import main

sys.exit(main())
