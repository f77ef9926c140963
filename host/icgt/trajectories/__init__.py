"""External trajectories for re-geotagging after the flight, and the exposure events for PPK tools.

* `icgt.trajectories.source`: the `PoseSource` interface and the interpolated `SampledTrajectory`;
* `icgt.trajectories.recorded`: the autopilot's telemetry as the recorder geotagged it, as a source;
* `icgt.trajectories.tum`: TUM trajectories (SLAM/VIO), `read_tum`;
* `icgt.trajectories.rtklib_pos`: RTKLIB .pos solutions (PPK), `read_pos`;
* `icgt.trajectories.regeotag`: `regeotag` (frames with positions from a source);
* `icgt.trajectories.ppk_events`: events_gpst.csv and Timestamp.MRK (`icgt export --formats ppk`);
* `icgt.trajectories.gpstime`: GPS week/TOW <-> UTC with the leap seconds;
* `icgt.trajectories.cli`: `icgt regeotag`.
"""
