"""The digital twin: a simulated F450 that speaks MAVLink and renders its cameras.

scene.py      the field, pads, obstacles and tasks (TOML, `scenes/field.toml`)
dynamics.py   rigid body, rotors, drag, wind, battery, ground and crashes (N vehicles)
control.py    PX4-like cascade: position, velocity, attitude, rate, mixer
commander.py  arming, modes, land detector, auto-disarm, failsafes
sensors.py    GPS, barometer, the autopilot's estimate
sim.py        all of the above on a sim clock: `Sim`, faster than real time
telemetry.py  MAVLink messages from the sim's state, as PX4 sends them
params.py     PX4-named parameters (read-only mirror of the configuration)
vehicle.py    the MAVLink vehicle on a UDP socket: `MavlinkVehicle`
runner.py     `Twin`: real-time thread, vehicle, `render()`, `pose()`
render.py     front and bottom cameras (numpy/OpenCV)
pilot.py      a scripted stick pilot for the paper's tasks
gym_env.py    `TwinEnv`, the Gymnasium environment
gym_vector.py `TwinVectorEnv`, N of them in one batched Sim
"""
