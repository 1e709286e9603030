"""fpgalink: host library for the FPGA motor-controller UART protocol."""

from fpgalink._framing import DEFAULT_FRAMING, FrameDecoder, Framing, encode_frame

__all__ = ["DEFAULT_FRAMING", "FrameDecoder", "Framing", "encode_frame"]
