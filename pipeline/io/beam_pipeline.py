"""A Beam pipeline under given options, without Beam's download at run time on the DirectRunner."""

from __future__ import annotations

import apache_beam as beam
from apache_beam.options.pipeline_options import PipelineOptions, StandardOptions


def pipeline_for(options: PipelineOptions) -> beam.Pipeline:
    """A pipeline under ``options``. On the DirectRunner it runs on Beam's FnApiRunner, built as the
    DirectRunner builds it for a batch pipeline: the DirectRunner would first try its Prism runner,
    which it downloads from the internet at run time (offline, it falls back after a delay)."""
    if options.view_as(StandardOptions).runner not in (None, "DirectRunner"):
        return beam.Pipeline(options=options)
    from apache_beam.portability.api import beam_provision_api_pb2
    from apache_beam.runners.portability.fn_api_runner import fn_runner
    from apache_beam.runners.portability.portable_runner import JobServiceHandle

    encoded = JobServiceHandle.encode_pipeline_options(options.get_all_options())
    provision = beam_provision_api_pb2.ProvisionInfo(pipeline_options=encoded)
    runner = fn_runner.FnApiRunner(provision_info=fn_runner.ExtendedProvisionInfo(provision))
    return beam.Pipeline(runner=runner, options=options)


def run_to_end(pipeline: beam.Pipeline):
    """Run ``pipeline`` and wait for its end; its result. Beam's Dask runner opens a
    distributed.Client for the run and never closes it: it is closed here, so a caller that goes on
    keeps no client trying to reconnect once the cluster is gone."""
    result = pipeline.run()
    try:
        result.wait_until_finish()
    finally:
        client = getattr(result, "client", None)
        if client is not None:
            client.close()
    return result
