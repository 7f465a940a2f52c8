"""The Python API: ``generate`` and ``make_dataset``, the commands ``plantdreamer generate``
and ``plantdreamer dataset`` as functions (``calls.py``).

They take the same settings by the same names (``_`` for ``-``: ``eval_views=2`` is
``--eval-views 2``), with the same defaults: every setting is a field of ``GenerateConfig``
(``plantdreamer.settings``), read from there to build each function's signature and the list
in its docstring, so ``help(plantdreamer.generate)`` shows them all. They check their
arguments as the command line does, through the same routines below both
(``pipeline.requested``, ``dataset.request``), before torch is imported or anything is
written; a flag is ``True`` or ``False``, never read by truthiness. Errors are the
package's own (``InputError``, ``ModelNotFoundError``, ``RunInterrupted``, ...: all
importable from ``plantdreamer``), never an exit, and speak of the API's keywords
(``words.py``). Each returns what a caller opens next, with absolute paths
(``results.py``): the files written, and the run's figures.
"""

from plantdreamer.api.calls import generate, make_dataset
from plantdreamer.api.results import DatasetResult, GeneratedPlant

__all__ = ["DatasetResult", "GeneratedPlant", "generate", "make_dataset"]
