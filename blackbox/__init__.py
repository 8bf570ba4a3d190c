"""Black box: event register, storage (MongoDB; embedded default), REST API and web GUIs."""
