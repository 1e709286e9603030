"""fpgaemu: cycle-level emulator of the FPGA motor-controller board."""

__all__: list[str] = []
