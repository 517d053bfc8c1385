"""Partners made of something learned or recorded, above the views and the learners: a saved run's frozen policy
(``policy``), a population of scripted and learned members (``population``), a behaviour clone of a Minari dataset
(``proxy``), and a team of scripted opponents sharing one view (``team``). Each joins the scripted opponents in
``sidewalk.registry.OPPONENTS``, so ``opponent=policy`` is chosen like ``opponent=dijkstra``. The folders beside them
hold the shipped learned partners (README.md)."""
