"""The base layer: models every other part shares, with no I/O and no imports from above.

Geodesy, the field scene, and MAVLink framing live here so that companion, twin, analysis
and server each keep only their own view of them. Nothing in `core` imports companion,
twin, analysis, server or web (tests/test_layers.py enforces the direction).
"""
