"""Safe outputs: atomic writes (temp file, then rename), one writer per output folder (lock.py), and the record
of what the tool wrote in a folder, so that --overwrite removes only that (outdir.py)."""
