"""Simulators: the schematic exact-geometry harbour (now) and the Blender renderer (later)."""
