#!/usr/bin/env python
"""Train an ACT policy: ``python train_act.py --help`` (the same command as ``controltac-train``;
its code is ``controltac_il.app.train_cli``)."""

import sys

from controltac_il.app.train_cli import main

if __name__ == "__main__":
    sys.exit(main())
