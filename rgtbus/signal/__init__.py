"""The signal layer (docs/model.md): codebooks, frequency plans, the medium and its channel, the
resonator bank, and decoding."""
