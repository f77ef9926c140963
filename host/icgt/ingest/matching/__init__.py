"""Match the camera card's JPEGs to the recorded exposures (`icgt match`); see `icgt.ingest.match`."""
