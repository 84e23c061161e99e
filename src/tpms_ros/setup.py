"""Everything is declared in setup.cfg; colcon and pip run this file."""

from setuptools import setup

setup()
