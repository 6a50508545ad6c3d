"""The digital twin: a simulated F450 that speaks MAVLink and renders its cameras."""
