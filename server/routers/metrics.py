"""GET /metrics: Prometheus text format, for the ship's (or shore's) monitoring."""

from __future__ import annotations

import shutil
from collections.abc import Iterator
from typing import Any

from fastapi import APIRouter
from fastapi.responses import Response
from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, generate_latest
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily

from server.deps import HubDep, SettingsDep, StoreDep
from storage import queries

router = APIRouter(tags=["metrics"])


class _Snapshot:
    """A collector over the ingest's last heartbeat and the store, read once per scrape."""

    def __init__(
        self,
        health: dict[str, Any] | None,
        ingest_up: bool,
        alarms: list[dict[str, Any]],
        disk_free: int,
        clients: int,
    ) -> None:
        self.health, self.ingest_up, self.alarms = health or {}, ingest_up, alarms
        self.disk_free, self.clients = disk_free, clients

    def collect(self) -> Iterator[Any]:
        h = self.health
        counters = h.get("counters") or {}
        yield GaugeMetricFamily(
            "camcal_ingest_up", "1 if the ingest's heartbeat is recent", value=int(self.ingest_up)
        )
        for name, key, doc in (
            ("camcal_frames_received", "frames_received", "frames received from modules"),
            ("camcal_frames_stored", "frames_stored", "frames committed to the store"),
            ("camcal_frames_analysed", "frames_analysed", "frames analysed"),
            (
                "camcal_resends",
                "duplicates",
                "messages received again (resends after a lost acknowledgement)",
            ),
            ("camcal_acks", "acks_sent", "acknowledgements sent"),
            ("camcal_sensor_batches_received", "sensor_batches_received", "sensor messages received"),
            (
                "camcal_analysis_restarts",
                "analysis_restarts",
                "analysis process pools replaced after a process died",
            ),
        ):
            yield CounterMetricFamily(name, doc, value=float(counters.get(key, 0)))
        rejected = CounterMetricFamily(
            "camcal_frames_rejected", "analysed frames rejected, by reason", labels=["reason"]
        )
        for key, value in counters.items():
            if key.startswith("result_") and key != "result_ok":
                rejected.add_metric([key[len("result_") :]], float(value))
        yield rejected
        malformed = CounterMetricFamily(
            "camcal_malformed_messages", "messages dropped as malformed, by kind", labels=["kind"]
        )
        for kind, value in (h.get("malformed") or {}).items():
            malformed.add_metric([kind], float(value))
        yield malformed
        nacked = CounterMetricFamily(
            "camcal_refused_messages", "messages refused with a nack, by reason", labels=["reason"]
        )
        for reason, value in (h.get("nacked") or {}).items():
            nacked.add_metric([reason], float(value))
        yield nacked
        queues = GaugeMetricFamily("camcal_queue_depth", "items waiting in the ingest", labels=["queue"])
        for q, value in (h.get("queues") or {}).items():
            queues.add_metric([q], float(value))
        yield queues
        latency = GaugeMetricFamily(
            "camcal_result_latency_seconds", "receive to stored result", labels=["quantile"]
        )
        for q, key in (("0.5", "latency_p50_s"), ("0.95", "latency_p95_s")):
            if h.get(key) is not None:
                latency.add_metric([q], float(h[key]))
        yield latency
        link = GaugeMetricFamily("camcal_module_link_up", "1 if the module's link is up", labels=["module"])
        age = GaugeMetricFamily(
            "camcal_module_last_packet_age_seconds", "age of the last packet", labels=["module"]
        )
        fps = GaugeMetricFamily("camcal_module_frames_per_second", "frames per second", labels=["module"])
        pending = GaugeMetricFamily(
            "camcal_module_outbox_pending", "messages not yet acknowledged", labels=["module"]
        )
        for m, st in (h.get("modules") or {}).items():
            link.add_metric([m], 1.0 if st.get("link") == "up" else 0.0)
            if st.get("last_packet_age_s") is not None:
                age.add_metric([m], float(st["last_packet_age_s"]))
            fps.add_metric([m], float(st.get("frames_per_s") or 0.0))
            pending.add_metric([m], float(st.get("outbox_pending") or 0))
        yield from (link, age, fps, pending)
        active = GaugeMetricFamily("camcal_alarms_active", "active alarms by severity", labels=["severity"])
        for sev in ("INFO", "MINOR", "MAJOR"):
            active.add_metric([sev], float(sum(1 for a in self.alarms if a["severity"] == sev)))
        yield active
        yield GaugeMetricFamily(
            "camcal_disk_free_bytes", "free bytes in the data folder", value=float(self.disk_free)
        )
        yield GaugeMetricFamily(
            "camcal_websocket_clients", "browsers connected live", value=float(self.clients)
        )


@router.get("/metrics", response_class=Response, responses={200: {"content": {"text/plain": {}}}})
def metrics(hub: HubDep, store: StoreDep, settings: SettingsDep) -> Response:
    """Frames received, stored, rejected by reason, acks, resends, queue depths, latencies, disk free."""
    alarms = store.call(queries.alarms, active=True)
    registry = CollectorRegistry(auto_describe=False)
    ingest = hub.ingest_state(settings.stale_after_s)
    registry.register(
        _Snapshot(
            hub.live_health(settings.stale_after_s),
            ingest["up"],
            alarms,
            shutil.disk_usage(store.files.root).free,
            len(hub.clients),
        )
    )
    return Response(generate_latest(registry), media_type=CONTENT_TYPE_LATEST)
