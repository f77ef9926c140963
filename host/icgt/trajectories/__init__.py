"""External trajectories for re-geotagging after the flight.

* `icgt.trajectories.source`: the `PoseSource` interface and the interpolated `SampledTrajectory`;
* `icgt.trajectories.recorded`: the autopilot's telemetry as the recorder geotagged it, as a source;
* `icgt.trajectories.tum`: TUM trajectories (SLAM/VIO), `read_tum`;
* `icgt.trajectories.rtklib_pos`: RTKLIB .pos solutions (PPK), `read_pos`;
* `icgt.trajectories.regeotag`: `regeotag` (frames with positions from a source);
* `icgt.trajectories.cli`: `icgt regeotag`.

The exposure events for PPK tools are an export (`icgt.export.ppk_events`); GPS week/TOW <-> UTC is
`icgt.clocks.gpstime`.
"""
