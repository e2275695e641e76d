"""Studies: the thesis reproduction, chapter studies, the Dask campaign, README/docs generators."""
