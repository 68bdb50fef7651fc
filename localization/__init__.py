"""Localization on the acoustic wall map (paper Fig. 1(b)).

Public faces (import from these, never from a private ``_name`` module):

- `localization.motion`: odometry motion model (AMCL alpha1-4);
- `localization.sensor`: likelihood of a heat map given a pose and G (config, lookup tables,
  measurement, two models);
- `localization.resampling`: log-weights and systematic resampling (numba kernel; numpy
  twin in the tests);
- `localization.particle_filter`: `ParticleFilter` (augmented MCL, KLD, checkpoints),
  `FilterConfig`, `run_filter`;
- `localization.calibration`: `calibrate_beta`, the sensor sharpness that makes the NEES
  honest;
- `localization.grid_filter`: exact histogram filter, the reference posterior;
- `localization.estimate`: `PoseEstimate`, modes, circular statistics, track metrics;
- `localization.posterior`: emcee pose posterior (issue 8).

This package never imports ``service``; it may import ``mapping``.
"""
