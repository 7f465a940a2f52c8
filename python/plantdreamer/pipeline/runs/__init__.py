"""The run's lifecycle: one run of N plants from the entry to the record (``entry.py``),
for a plant alone, a group and a dataset unit alike: the record (``record.py``), where the
plants live (``layout.py``), what is done with each (``plan.py``), each part's start,
training and export (``start.py``, ``sequence.py``) and what comes back (``results.py``).
"""
