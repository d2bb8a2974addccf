"""Design trade studies: a study file's cases (:mod:`.study`), run on dask.distributed
(:mod:`.engine`, each case by :mod:`.case` through ``simulate()`` and
``metrics.summarize``), scored (:mod:`.metrics`) and written (:mod:`.results`,
:mod:`.report`). The command is ``lunar-drake trade``."""
