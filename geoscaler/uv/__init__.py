"""UV space: charts and the texels views reach, chart packing with xatlas, the layout planner and
the bake into a new layout, the ``--uv`` modes."""
