"""Every file format dcseg reads or writes, and nothing else: stages never open files."""
