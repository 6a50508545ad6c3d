"""Flight analysis: the paper's task metrics, plots and comparisons (geodesy and the
scene model are the base layer's: core.geodesy, core.scene).

recording  open_recording: the one reader of a session folder, zip or .tlog (a tlog
           replayed through the link's StateTracker into telemetry.csv's rows)
track      Track (typed numpy columns, one sample per GPS message) and its loader:
           load_track(path) for a session folder, zip, telemetry.csv or .tlog
csvcols    fast column cutting of the recorder's telemetry.csv
flight_frame  align_track: ENU about the arming point, +x towards the reference; the
           origin and turn the replay view uses too
flights    split_flights / track_flights: a track's flights (armed periods with a
           take-off), with their arming, take-off, landing and disarming samples
field_layout  the scene's pads and obstacles in a track's frame; obstacle contacts
tasks      trial, windows and metrics of the four tasks (TaskParams, TaskResult)
compare    one table in the paper's layout (Markdown, CSV, JSON)
plots      3D, bird's-eye and position-history figures (PNG)
report     analyze_paths / analyze_tracks: what the CLI and REST both call
cli        `fpv-station analyze`
errors     AnalysisError and its kinds
"""
