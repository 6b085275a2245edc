"""Getting recordings into lfd: ``lfd.io.recordings`` (CSV joint and landmark recordings, resampled)
and the ``lfd-import`` command (``lfd.io.import_csv``)."""
