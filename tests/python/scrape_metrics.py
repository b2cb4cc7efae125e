"""Scrapes a Prometheus endpoint and parses it with Prometheus' own client parsers.

Usage: scrape_metrics.py URL

Parses the body with prometheus_client.parser.text_string_to_metric_families
(the Prometheus text format) and with the OpenMetrics parser when the server
says it speaks OpenMetrics, and prints one JSON object: the content type, and
every sample as [name, labels, value] from the Prometheus text parser, plus the
families' types. Exits non-zero when either parser refuses the body.
"""

import json
import sys
import urllib.request

from prometheus_client.openmetrics.parser import (
    text_string_to_metric_families as openmetrics_families,
)
from prometheus_client.parser import text_string_to_metric_families


def main() -> None:
    with urllib.request.urlopen(sys.argv[1], timeout=10) as response:
        content_type = response.headers.get("Content-Type", "")
        body = response.read().decode("utf-8")
    families = list(text_string_to_metric_families(body))
    openmetrics = None
    if content_type.startswith("application/openmetrics-text"):
        openmetrics = sorted(f.name for f in openmetrics_families(body))
    print(json.dumps({
        "content_type": content_type,
        "types": {f.name: f.type for f in families},
        "samples": [[s.name, s.labels, s.value] for f in families for s in f.samples],
        "openmetrics_families": openmetrics,
    }))


if __name__ == "__main__":
    main()
