"""One frame → the array's angles.

``frames`` reads and undistorts video frames, ``edges`` finds the phantom's walls, ``registration``
fits the Eq. (1) spiral channel to them (centre, rotation, scale, mirror), ``angles`` measures
theta_tip, theta_bot and theta_con in a registered frame, ``geometry`` holds the phantom and array,
``rendering`` and ``drawing`` make synthetic frames and annotated ones.
"""
