"""Learning from flights (the `learn` extra, not needed on the Pi).

recording_reader  a session folder, zip or bare tlog opened for export (columns, frames, tlog)
episodes       one episode per flight: the twin env's state, the pilot's sticks, frames
export         `fpv-station export`: recordings streamed into a format's writer
lerobot        LeRobot v3.0 datasets (pyarrow + PyAV)
minari_export  Minari datasets whose env is the twin's TwinEnv
mcap_export    MCAP with Foxglove schemas, one file per episode
stats          LeRobot-style feature statistics
demos          `fpv-station demos`: the scripted pilot flown into ordinary sessions
cli            the commands
"""
