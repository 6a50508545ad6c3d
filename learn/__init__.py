"""Learning from flights (the `learn` extra, not needed on the Pi).

episodes       one episode per flight (recordings opened by analysis.recording): the twin
               env's state, the pilot's sticks, frames; the telemetry COLUMNS they read
export         `fpv-station export`: recordings streamed into a format's writer
lerobot        LeRobot v3.0 datasets (pyarrow + PyAV)
minari_export  Minari datasets whose env is the twin's TwinEnv
mcap_export    MCAP with Foxglove schemas, one file per episode
stats          LeRobot-style feature statistics
demos          `fpv-station demos`: the scripted pilot flown into ordinary sessions
cli            the commands
"""
