//! `soundmap.v1.Monitoring`: state snapshots, the estimate stream, operator control.
//!
//! Every call is authorized first ([`Authenticator::authorize_operator`]):
//! `GetState` and `WatchEstimates` need role `read`, `SetActivePositioning`
//! and `SetFocus` role `control`.

use std::pin::Pin;
use std::sync::Arc;

use futures::Stream;
use soundmap_proto::wire;
use soundmap_proto::wire::monitoring_server::Monitoring;
use tokio::sync::broadcast::error::RecvError;
use tokio::sync::{broadcast, mpsc, oneshot};
use tonic::{Request, Response, Status};

use super::actor;
use super::auth::Authenticator;
use super::status::{self, to_status};
use crate::config::Role;
use crate::coordinator::PositioningUpdate;

/// The monitoring service.
#[derive(Debug, Clone)]
pub struct MonitoringService {
    requests: mpsc::Sender<actor::Request>,
    estimates: broadcast::Sender<Arc<wire::SourceEstimate>>,
    stopping: tokio::sync::watch::Receiver<bool>,
    auth: Authenticator,
}

impl MonitoringService {
    /// A service reading the coordinator task's state and estimate stream.
    pub fn new(
        requests: mpsc::Sender<actor::Request>,
        estimates: broadcast::Sender<Arc<wire::SourceEstimate>>,
        stopping: tokio::sync::watch::Receiver<bool>,
    ) -> Self {
        MonitoringService { requests, estimates, stopping, auth: Authenticator::default() }
    }

    /// The same service with calls authorized by `auth`.
    pub fn with_auth(self, auth: Authenticator) -> Self {
        MonitoringService { auth, ..self }
    }

    fn authorize<T>(&self, request: &Request<T>, role: Role) -> Result<(), Status> {
        self.auth.authorize_operator(request, role).map_err(|e| to_status(&e))
    }
}

type EstimateStream = Pin<Box<dyn Stream<Item = Result<wire::SourceEstimate, Status>> + Send>>;

#[tonic::async_trait]
impl Monitoring for MonitoringService {
    type WatchEstimatesStream = EstimateStream;

    async fn get_state(
        &self,
        request: Request<wire::GetStateRequest>,
    ) -> Result<Response<wire::CoordinatorState>, Status> {
        self.authorize(&request, Role::Read)?;
        let (reply, answer) = oneshot::channel();
        self.requests.send(actor::Request::GetState { reply }).await.map_err(|_| status::shutting_down())?;
        Ok(Response::new(answer.await.map_err(|_| status::shutting_down())?))
    }

    async fn watch_estimates(
        &self,
        request: Request<wire::WatchEstimatesRequest>,
    ) -> Result<Response<Self::WatchEstimatesStream>, Status> {
        self.authorize(&request, Role::Read)?;
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
        self.authorize(&request, Role::Control)?;
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
        self.authorize(&request, Role::Control)?;
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
