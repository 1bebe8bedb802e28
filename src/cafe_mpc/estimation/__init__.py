"""State estimation as on the robot: the controller's ``Measurement`` from the robot's own sensors.

``estimator.StateEstimator`` turns ``core.sensors.SensorReadings`` (IMU and joint encoders) into the
``core.measurement.Measurement`` every controller reads: orientation and angular velocity from the IMU, base
position and linear velocity from a linear Kalman filter that fuses the IMU's acceleration with the leg
kinematics of the feet in stance (the MIT Cheetah 3 / Mini Cheetah design; ``estimator``), contacts from
the plan (``contacts``). ``controller.SensingController`` puts it in front of any controller. Its settings
are the run config's ``kinematic_kf`` section, ``config.estimation.KinematicKFSettings`` (``mit()``: MIT's
published tuning).

This package is the controller's: it never imports the simulator (``tests/test_layers.py``).
"""
