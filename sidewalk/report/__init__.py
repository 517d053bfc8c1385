"""Reports over run folders: learning curves, final values with confidence intervals, and the paper's figures.

``write_report(paths, out)`` finds every run folder under ``paths`` (a folder holding ``config.yaml`` and
``metrics.csv``, as ``runners/main.py`` writes it, alone or inside a sweep), groups the runs into *conditions*
(identical configs but for the seed and bookkeeping keys such as the logger; a shielded learner is a condition
of its own), and writes into ``out``:

- ``figures/curves_<family>.png``: success and collision rate of each agent over training, the mean over seeds
  with the standard error shaded (the paper's way); one figure per *family*, i.e. per sweep folder (the folder
  holding Hydra's ``multirun.yaml``), or per parent folder for runs outside a sweep;
- ``figures/cost_<family>.png``: the cost the learner's agents paid during training (collisions), cumulative
  over frames, one line per condition, the mean over seeds with the standard error shaded; drawn where runs log
  ``train/cumulative_cost`` (runs written before the safety accounting have no such figure);
- the paper's figures where runs that differ in the figure's variable are present (see ``PAPER_FIGURES``):
  Fig. 5 success and Fig. 7 collisions by opponent, Fig. 6 success under noise, Fig. 8 explicit vs implicit
  reward, and Fig. 10 representative trajectories replayed from the runs' checkpoints; a figure whose runs are
  missing is skipped with a note;
- ``report.md``: the tables (final values of each condition: mean ± standard error over seeds, interquartile mean
  with its 95 % stratified-bootstrap interval, see ``sidewalk.stats``) with the figures embedded by relative path,
  and, beside each family's final values, Safety Gym's triple (final return, final cost, training cost rate) and
  the shield's rate where runs log it; and the run folders that were skipped and why (no ``metrics.csv``, a
  truncated CSV, no ``summary.json``, a failed job...);
- under each paper figure, rliable's aggregates over its panels (``aggregates``) and, for Fig. 5, which compares
  learners, ``figures/fig5_performance_profile.png``: the fraction of runs above each threshold, with its band;
- ``report.csv``: every number in ``report.md``, one per row; ``curves.csv``: every plotted point.

Learning curves read the ``eval/<agent>/<metric>`` columns of ``metrics.csv`` (the evaluations during training);
final values read ``summary.json`` (the last evaluation). Agents are ``ego``/``other`` where a learner plays
against a scripted opponent and ``agent0``/``agent1``/... where it plays every agent (centralized).

The modules, each importing only those listed above it (``tests/test_report_imports.py`` holds them to it):

- ``runs``: finding run folders and reading their config, metrics and summary, or saying why not;
- ``conditions``: runs grouped into conditions and labelled; the paper's figures as panels of conditions;
- ``tables``: curves, final values with mean ± SE and IQM intervals, ``report.csv``'s rows, Markdown tables;
- ``checkpoints``: a run's config and learner rebuilt from its folder, its final evaluation replayed;
- ``figures``: learning curves, the paper's figures and Fig. 10's trajectories, drawn with their report.md lines;
- ``aggregates``: a paper figure's compared settings pooled over its panels (IQM, stratified-bootstrap interval) and
  the performance profile of a figure that compares learners;
- ``crossplay``: the cross-play matrix of a ``runners/crossplay.py`` folder, its heatmaps and report.md section;
- ``claims``: the paper's claims (its §6.2) held against the runs, a verdict each;
- ``document``: ``write_report``, which puts ``report.md`` together and writes the files.

Import each name from the module that defines it (``from sidewalk.report.document import write_report``).
"""
