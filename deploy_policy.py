#!/usr/bin/env python
"""Run a trained ACT policy: ``python deploy_policy.py --help`` (the same command as ``controltac-deploy``;
its code is ``controltac_il.app.deploy_cli``)."""

import sys

from controltac_il.app.deploy_cli import main

if __name__ == "__main__":
    sys.exit(main())
