"""Localization on the acoustic wall map (paper Fig. 1(b)).

``motion``           odometry motion model (AMCL alpha1-4)
``sensor``           likelihood of a HeatMap given a pose and G (lookup tables, two models);
                     its parts: ``sensor_config``, ``sensor_tables``, ``sensor_measurement``
``resampling``       log-weights and systematic resampling (numba + numpy twin)
``particle_filter``  ParticleFilter (augmented MCL, KLD, checkpoints) and run_filter
``filter_config``    FilterConfig, the particle filter's parameters
``calibration``      calibrate_beta: the sensor sharpness that makes the NEES honest
``grid_filter``      exact histogram filter, the reference posterior
``estimate``         PoseEstimate, modes, circular statistics, track metrics
``posterior``        emcee pose posterior (issue 8)

This package never imports ``service``.
"""
