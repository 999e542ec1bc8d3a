"""The engine: the SimPy world (``sim``) and the units' ears (``hearing``), docs/engine.md.

The world moves from event to event over a bus, to the smallest promise of silence of every
member; the ears advance the resonator banks of the units one process runs, as arrays. The
engine knows a unit only through ``Member`` and hands it what it heard through the ears."""
