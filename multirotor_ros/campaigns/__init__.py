"""Batch work on Dask: fault-diagnosis campaigns, hidden-effect sweeps, identify/discrepancy over many logs.

A campaign is a list of cases, each a pure function of its description (seed included), run by
:mod:`~multirotor_ros.campaigns.engine` on a Dask cluster (a local one sized to the machine, or an
existing one given by its scheduler's address). Results stream to Parquet (:mod:`.store`) as they finish,
so an interrupted campaign resumes where it stopped; :mod:`.report` writes the terminal summary and one
self-contained HTML page. The kinds of campaign are the modules :mod:`.fault`, :mod:`.recovery`
(fault-tolerant flight), :mod:`.sweep` and :mod:`.logs`, each with ``run_case(description) -> row``,
``summary(rows)`` and ``figures(rows)``.
"""
