"""What the commands write: ``atomic`` (whole files or none, with a PDF twin for every
PNG), ``plots`` (the shared figures) and ``export`` (VTU for ParaView)."""
