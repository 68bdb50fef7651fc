"""The ``omnisonar`` subcommands, one module per command group.

``runs`` (signal, scenes, import-run, export-run), ``simulate``, ``maps`` (heatmap, build-map,
evaluate-map), ``localize`` (localize, calibrate, posterior) and ``serve`` (serve, demo-api,
demo). Each module defines ``_add_<name>(subparsers)`` functions that register a parser and a
handler; `service.cli` collects them. They are edges over ``mapping`` and ``localization``:
they parse arguments, read and write files, print and plot, and compute nothing themselves.
"""
