"""GET /metrics: Prometheus text from the ingest's heartbeat and the store."""

from __future__ import annotations

from fastapi.testclient import TestClient
from prometheus_client.parser import text_string_to_metric_families

from server.app import create_app
from server.settings import ServerSettings


def test_metrics_in_prometheus_format(tmp_path) -> None:
    app = create_app(ServerSettings(data_dir=tmp_path / "data", events=None))
    with TestClient(app) as client:
        hub = app.state.hub
        hub.record_health(
            {
                "modules": {
                    "A": {"link": "up", "last_packet_age_s": 0.2, "frames_per_s": 1.5, "outbox_pending": 3},
                    "B": {
                        "link": "down",
                        "last_packet_age_s": 12.0,
                        "frames_per_s": 0.0,
                        "outbox_pending": 40,
                    },
                },
                "queues": {"store": 2, "analysis_backlog": 5},
                "counters": {
                    "frames_received": 100,
                    "frames_stored": 98,
                    "duplicates": 4,
                    "acks_sent": 60,
                    "result_ok": 80,
                    "result_saturated": 12,
                    "result_too_dark": 3,
                    "analysis_restarts": 1,
                },
                "malformed": {"bad_header": 2},
                "latency_p50_s": 0.08,
                "latency_p95_s": 0.21,
            }
        )
        r = client.get("/metrics")
        assert r.status_code == 200 and r.headers["content-type"].startswith("text/plain")
        samples = {
            (s.name, tuple(sorted(s.labels.items()))): s.value
            for fam in text_string_to_metric_families(r.text)
            for s in fam.samples
        }
    assert samples[("camcal_ingest_up", ())] == 1
    assert samples[("camcal_frames_stored_total", ())] == 98
    assert samples[("camcal_resends_total", ())] == 4
    assert samples[("camcal_analysis_restarts_total", ())] == 1
    assert samples[("camcal_frames_rejected_total", (("reason", "saturated"),))] == 12
    assert samples[("camcal_malformed_messages_total", (("kind", "bad_header"),))] == 2
    assert samples[("camcal_queue_depth", (("queue", "analysis_backlog"),))] == 5
    assert samples[("camcal_result_latency_seconds", (("quantile", "0.95"),))] == 0.21
    assert samples[("camcal_module_link_up", (("module", "B"),))] == 0
    assert samples[("camcal_disk_free_bytes", ())] > 0
