"""fmu-opinf: stable second-order reduced models of constrained mechanical systems.

Pipeline, one module per stage::

    source -> snapshots -> basis -> inference -> rom -> compare (-> report) / export

(``fit`` drives basis and inference into a ``rom``: order, extra terms, refinement, training checks.)
"""

__version__ = "0.1.0"
