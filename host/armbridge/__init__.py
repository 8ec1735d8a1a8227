"""armbridge: host runtime and firmware for research robot arms."""

__version__ = "0.1.0"
