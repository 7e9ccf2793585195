"""``observer_gym/TargetFollower-v0``: a wheeled robot with a tilt camera follows a target."""
