"""Constants shared with dm_control's composer."""

# MuJoCo visual group for invisible sensor sites (e.g. position detectors).
SENSOR_SITES_GROUP = 4
