"""The dcseg worker: queue -> job folder -> dcseg stages. Empty so imports stay light."""
