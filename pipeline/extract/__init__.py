"""Video → angles: one video's frames through registration and measurement (a state machine that
re-registers when the camera moves), the kinematics check, batches of videos (locally or on Dask),
and annotated frames for checking by eye."""
