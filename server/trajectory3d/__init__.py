"""The 3D trajectory: a viser scene of the flight in East-North-Up, live and replayed.
The field drawn is the one scene model (`core.scene.Scene`).

pose.py          attitude (NED/FRD Euler) -> ENU/FLU rotation, camera footprint on the ground
colors.py        colour-coding of the trail by height or speed (the server's one ramp)
trail.py         the flown path as chunks of samples, with gaps and a movable origin
live_scene.py    draws field, vehicle, home, footprint and trail into a viser scene
controls.py      the GUI in the viser panel (follow, clear, colour-coding, field)
service.py       the live viser server started with the station, fed from `station.state`
replay.py        a recorded session as ENU arrays with times and frame names, in the
                 analysis' flight frame
replay_scene.py  the replay's own viser server: a session's path, its frames, the field
"""
