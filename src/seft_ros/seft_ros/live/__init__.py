"""The live view of a running test: Foxglove and a web page, outside the real-time loop.

``seft run --live [HOST][:PORT]`` starts it (:mod:`seft_ros.cli.live`): a process of its own
(:mod:`seft_ros.live.node`) that reads the graph's record batches with best-effort
subscriptions, decimates them to a display rate (:mod:`seft_ros.live.channels`), keeps the
current run's shown samples and state (:mod:`seft_ros.live.view`), and serves them to
Foxglove (:mod:`seft_ros.live.foxglove_sink`) and to a plain web page
(:mod:`seft_ros.live.web`, ``static/``), with the access rules of :mod:`seft_ros.live.access`.

``static/uPlot.iife.min.js`` and ``static/uPlot.min.css`` are uPlot 1.6.32 (MIT,
``static/LICENSE.uPlot``), the ``dist/`` files of the npm package ``uplot`` unchanged
(``npm pack uplot@1.6.32``; sha256 19c8d4c6... and df630c6a...).
"""
