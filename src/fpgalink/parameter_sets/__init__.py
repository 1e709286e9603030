"""Parameter sets that ship with fpgalink, loadable by name: ``fpgalink-cli param load NAME``
(the TOML format of :mod:`fpgalink.protocol.paramfile`)."""
