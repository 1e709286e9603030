"""``python -m fpgalink`` is ``fpgalink-cli``."""

from fpgalink.cli import main

if __name__ == "__main__":
    main()
