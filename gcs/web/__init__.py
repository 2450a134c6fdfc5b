"""The web ground station: `python -m gcs.web --mavlink URL --zenoh ENDPOINT` (jsar-gcs-web); see __main__."""
