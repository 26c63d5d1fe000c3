"""Design studies: many jig designs through simulation and estimation, on a local pool or a Ray cluster.

:mod:`~softjig.study.spec` reads a study file and builds its designs, :mod:`~softjig.study.run` executes
its tasks, :mod:`~softjig.study.results` streams and aggregates the results; the report, the Pareto front
and the best rigs are :mod:`~softjig.study.report`, :mod:`~softjig.study.pareto`, :mod:`~softjig.study.best`.
"""
