"""Everything the paper describes: signal, heat map, simulators, files, the wall map G.

Public faces (import from these, never from a private ``_name`` module):

- `mapping.signal`: sonar configuration (Table 1) and the transmitted signal;
- `mapping.angles`: ``wrap_angle``, circular statistics, ``pose_error``;
- `mapping.run`: the run record (blocks, odometry, tracked poses);
- `mapping.files`: run, map and recording file formats, atomic writes;
- `mapping.scene`: wall segments as JSON, built-in scenes;
- `mapping.synthetic`: the analytic echo, the independent truth of the tests;
- `mapping.path`: constant-speed trajectories, built-in paths;
- `mapping.heatmap`: the Doppler heat map (eq. 1) and its resampling bank;
- `mapping.grid`: the map G by back-projection (Sec. 2.2, eqs. 2-5);
- `mapping.wallmap`: G on a Cartesian grid, the fitted walls, the observed cells;
- `mapping.coverage`: the cells the runs observed (range and line of sight);
- `mapping.reconstruct`: beyond the paper, inverting the back-projection;
- `mapping.quality`: wall-level and raster precision/recall against true walls;
- `mapping.build`: batch map building (processes, dask);
- `mapping.recording`: real recordings to run blocks and back (pure arrays);
- `mapping.simulate`: forward models, with `mapping.simulate.ism` (image source, the default)
  and `mapping.simulate.fdtd` (the paper's FDTD, the reference);
- `mapping.compare`: the FDTD against the image-source engine;
- `mapping.numba_config`: compile flags shared by every numba kernel.

This package never imports ``localization`` or ``service``; only `mapping.files` reads or
writes files.
"""
