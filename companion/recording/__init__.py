"""Synchronized flight recording: one session folder per flight (see `layout` for the format).

Modules: `layout` (names and columns), `meta` (session.json), `store` (safe access to the
sessions directory), `ondisk` (a cut-off session counted from its files), `recovery`.
"""
