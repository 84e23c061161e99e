"""Fault-injection tests import the shared ``harness`` module of this folder (pytest runs in
importlib mode, which puts no test folder on the path)."""

from pathlib import Path
import sys

sys.path.insert(0, str(Path(__file__).parent))
