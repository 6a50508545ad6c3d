"""Flight analysis: geodesy, the paper's task metrics, plots and comparisons.

track      Track (typed numpy columns, one sample per GPS message) and its loaders:
           load_track(path) for a session folder, zip, telemetry.csv or .tlog
csvcols    fast column cutting of the recorder's telemetry.csv
tlog       Track from a bare .tlog (pymavlink decodes only what analysis reads)
geodesy    WGS-84 -> ENU, the paper's start-to-reference alignment
frame      align_track: ENU about the arming point, +x towards the reference
flights    split_flights / track_flights: a track's flights (armed periods with a
           take-off), with their arming, take-off, landing and disarming samples
field      the twin scene's pads and obstacles, in a track's frame; contacts
tasks      trial, windows and metrics of the four tasks (TaskParams, TaskResult)
compare    one table in the paper's layout (Markdown, CSV, JSON)
plots      3D, bird's-eye and position-history figures (PNG)
report     analyze_paths / analyze_tracks: what the CLI and REST both call
cli        `fpv-station analyze`
synthetic  flights with known answers, written as sessions and tlogs
errors     AnalysisError and its kinds
"""
