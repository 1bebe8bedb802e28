"""The controller on a robot: start-up checks, stand-up, the MPC on the wire, safety limits, lie-down.

``runner.Deployment`` runs a ``cafe_mpc.Controller`` (``process`` mode) against a ``robot_io.RobotInterface``
(``cafe-mpc deploy``; docs/deploy.md); ``settings.DeploySettings`` holds its timings and limits,
``startup`` the checks that refuse to start, ``limits.CommandLimiter`` the limits every command is held to.
"""
