"""MAVLink on the wire and on disk: the one place that reads a packet header.

`framing` cuts a byte stream into packets (MAVLink 1 and 2 mixed, signed packets,
garbage between them) and reads header fields; `tlog_records` writes and reads the
`.tlog` record format (8-byte big-endian microsecond time, then one packet), finding
each packet's length with `framing`'s rules.
"""
