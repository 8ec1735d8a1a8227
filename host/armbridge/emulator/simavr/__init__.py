"""The simavr harness (harness.c, built on first use by simavr_chip.harness_binary)
and the ATmega2560's pin and ELF data (mega2560)."""
