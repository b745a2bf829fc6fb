"""One module per ``motorid`` command, each with ``add_..._arguments(parser)`` and ``run_...(args) -> int``.

``identify`` (:mod:`~motorid.commands.identify`), ``import``
(:mod:`~motorid.commands.importing`), ``simulate``, ``demo``, ``live``, ``control``,
``design``, ``sweep`` and ``bench``; :data:`motorid.cli.COMMANDS` loads each when it runs.
"""
