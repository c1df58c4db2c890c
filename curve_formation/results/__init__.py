"""What a run leaves in its folder (outputs), the report over it (report) and where it came
from (provenance).
"""
