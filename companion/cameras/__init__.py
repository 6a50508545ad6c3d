"""The station's cameras: sources chosen by spec, one capture thread each, shared JPEG frames.

    spec.py         parse the URL-like camera specs (`v4l2:/dev/video0?...`, `sim:front`, ...)
    source.py       the source interface every source implements
    v4l2.py         USB / V4L2 through OpenCV, MJPEG passthrough
    media.py        a video file or an image folder, looped
    twin_cameras.py the digital twin's rendered cameras
    airsim.py       AirSim / Cosys-AirSim over msgpack-rpc (client in msgpack_rpc.py)
    capture.py      Camera: the capture thread, NO SIGNAL, back-off, figures
    rig.py          build the station's cameras from the settings
    devices.py      list V4L2 devices and their formats (`fpv-station cameras`)

Import the submodules; this package imports nothing so that settings validation can
use `spec` without loading OpenCV.
"""
