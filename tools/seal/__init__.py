"""The image header's seal at link time (`seal.py`, run by `linker`, the firmware's linker)."""
