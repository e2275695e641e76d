"""Studies: the thesis reproduction, chapter studies, the Dask campaign, the README/docs generators."""
