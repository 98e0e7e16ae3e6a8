"""Compensators: fit a correction of the systematic localisation error on training placements, apply
it.

Fit nodes (reduce over the ``Location`` collection, split ``train``): ``compensator.none``,
``.polynomial``, ``.disparity_curve``, ``.lookup``, ``.xyz``; ``compensator.apply`` corrects each
item. Pure functions ``fit_<model>`` / ``predict_<model>`` live in the node modules; the apply
table is :data:`nodes.compensators._table.PREDICTORS`.
"""
