"""The emulator's tests run against both firmwares where they ask for it:
``firmware_kind`` (the Python model, then the C core) and ``each_firmware`` (every
``Host.make()`` of the test builds that one); see tests/support/firmwares.py."""

from tests.support.firmwares import each_firmware, firmware_kind

__all__ = ["each_firmware", "firmware_kind"]
