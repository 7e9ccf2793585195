"""The ``observer-gym`` command and the experiment layer behind it."""
