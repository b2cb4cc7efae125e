//! `soundmap.v1.Monitoring`: state snapshots, the estimate stream, operator control.

use std::pin::Pin;
use std::sync::Arc;

use futures::Stream;
use soundmap_proto::wire;
use soundmap_proto::wire::monitoring_server::Monitoring;
use tokio::sync::broadcast::error::RecvError;
use tokio::sync::{broadcast, mpsc, oneshot};
use tonic::{Request, Response, Status};

use super::actor;
use super::status::{self, to_status};
use crate::coordinator::PositioningUpdate;

/// The monitoring service.
#[derive(Debug, Clone)]
pub struct MonitoringService {
    requests: mpsc::Sender<actor::Request>,
    estimates: broadcast::Sender<Arc<wire::SourceEstimate>>,
    stopping: tokio::sync::watch::Receiver<bool>,
}

impl MonitoringService {
    /// A service reading the coordinator task's state and estimate stream.
    pub fn new(
        requests: mpsc::Sender<actor::Request>,
        estimates: broadcast::Sender<Arc<wire::SourceEstimate>>,
        stopping: tokio::sync::watch::Receiver<bool>,
    ) -> Self {
        MonitoringService { requests, estimates, stopping }
    }
}

type EstimateStream = Pin<Box<dyn Stream<Item = Result<wire::SourceEstimate, Status>> + Send>>;

#[tonic::async_trait]
impl Monitoring for MonitoringService {
    type WatchEstimatesStream = EstimateStream;

    async fn get_state(
        &self,
        _: Request<wire::GetStateRequest>,
    ) -> Result<Response<wire::CoordinatorState>, Status> {
        let (reply, answer) = oneshot::channel();
        self.requests.send(actor::Request::GetState { reply }).await.map_err(|_| status::shutting_down())?;
        Ok(Response::new(answer.await.map_err(|_| status::shutting_down())?))
    }

    async fn watch_estimates(
        &self,
        _: Request<wire::WatchEstimatesRequest>,
    ) -> Result<Response<Self::WatchEstimatesStream>, Status> {
        let rx = self.estimates.subscribe();
        // The stream ends when the coordinator shuts down.
        let stream = futures::stream::unfold(
            (rx, 0u64, self.stopping.clone()),
            |(mut rx, mut lagged, mut stop)| async move {
                loop {
                    let next = tokio::select! {
                        biased;
                        _ = stop.wait_for(|s| *s) => return None,
                        r = rx.recv() => r,
                    };
                    match next {
                        Ok(e) => {
                            let mut e = (*e).clone();
                            e.lagged = lagged;
                            return Some((Ok(e), (rx, 0, stop)));
                        }
                        Err(RecvError::Lagged(n)) => lagged += n,
                        Err(RecvError::Closed) => return None,
                    }
                }
            },
        );
        Ok(Response::new(Box::pin(stream)))
    }

    async fn set_active_positioning(
        &self,
        request: Request<wire::SetActivePositioningRequest>,
    ) -> Result<Response<wire::ActivePositioning>, Status> {
        let update = PositioningUpdate::from_wire(request.get_ref());
        let (reply, answer) = oneshot::channel();
        self.requests
            .send(actor::Request::SetActivePositioning { update, reply })
            .await
            .map_err(|_| status::shutting_down())?;
        let settings = answer.await.map_err(|_| status::shutting_down())?.map_err(|e| to_status(&e))?;
        Ok(Response::new(settings.to_wire()))
    }

    async fn set_focus(
        &self,
        request: Request<wire::SetFocusRequest>,
    ) -> Result<Response<wire::Focus>, Status> {
        let source_id = request.get_ref().source_id;
        let (reply, answer) = oneshot::channel();
        self.requests
            .send(actor::Request::SetFocus { source_id, reply })
            .await
            .map_err(|_| status::shutting_down())?;
        let source_id = answer.await.map_err(|_| status::shutting_down())?.map_err(|e| to_status(&e))?;
        Ok(Response::new(wire::Focus { source_id }))
    }
}
