"""``observer_gym/BallCatcher-v0``: an arm carries a box with a hole; a ball is thrown."""
