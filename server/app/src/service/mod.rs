//! The `cathlab.v1.Simulator` service: thin handlers that authenticate the bearer token,
//! validate the message (through `cathlab-api`), call the engine and convert the answer.
//! Streams forward the newest value of the engine's latest-value channels.
//!
//! This file owns the tonic trait implementation, each RPC handed to the module of its role:
//! `sessions` (scenes; sessions created, listed, read and closed; their anatomy), `control`
//! (commands and the control stream), `streams` (state, frames, events and metrics),
//! `reports` (reports, histories, replays), `accounts`, and `fleet` (the other servers'
//! sessions). Beneath them: `info` (`SessionInfo`), `access` (who may do what), `state` (the
//! service, its builders and its bookkeeping) and `wire` (what needs no state). Each module
//! uses only modules named after it here, never this file.

mod access;
mod accounts;
mod control;
mod fleet;
mod info;
mod reports;
mod sessions;
mod state;
mod streams;
mod wire;

use cathlab_api::pb;
use cathlab_api::pb::simulator_server::Simulator;
use tonic::{Request, Response, Status, Streaming};

pub use self::reports::replay_stored;
pub use self::sessions::{DEFAULT_PAGE_SIZE, MAX_PAGE_SIZE};
pub use self::state::{Role, SimulatorService};
pub use self::wire::ResponseStream;

// Each RPC's body is the inherent method of the same name in its role's module: Rust looks
// inherent methods up before trait methods, so `SimulatorService::name(self, request)` below
// is that method, not this trait's.
#[tonic::async_trait]
impl Simulator for SimulatorService {
    async fn list_scenes(
        &self,
        request: Request<pb::ListScenesRequest>,
    ) -> Result<Response<pb::ListScenesResponse>, Status> {
        SimulatorService::list_scenes(self, request).await
    }

    async fn create_session(
        &self,
        request: Request<pb::CreateSessionRequest>,
    ) -> Result<Response<pb::CreateSessionResponse>, Status> {
        SimulatorService::create_session(self, request).await
    }

    async fn list_sessions(
        &self,
        request: Request<pb::ListSessionsRequest>,
    ) -> Result<Response<pb::ListSessionsResponse>, Status> {
        SimulatorService::list_sessions(self, request).await
    }

    async fn get_session(
        &self,
        request: Request<pb::GetSessionRequest>,
    ) -> Result<Response<pb::SessionInfo>, Status> {
        SimulatorService::get_session(self, request).await
    }

    async fn close_session(
        &self,
        request: Request<pb::CloseSessionRequest>,
    ) -> Result<Response<pb::CloseSessionResponse>, Status> {
        SimulatorService::close_session(self, request).await
    }

    async fn send_command(
        &self,
        request: Request<pb::SendCommandRequest>,
    ) -> Result<Response<pb::CommandAck>, Status> {
        SimulatorService::send_command(self, request).await
    }

    type ControlStream = ResponseStream<pb::ControlOutput>;

    async fn control(
        &self,
        request: Request<Streaming<pb::ControlInput>>,
    ) -> Result<Response<Self::ControlStream>, Status> {
        SimulatorService::control(self, request).await
    }

    type StreamStateStream = ResponseStream<pb::DeviceState>;

    async fn stream_state(
        &self,
        request: Request<pb::StreamStateRequest>,
    ) -> Result<Response<Self::StreamStateStream>, Status> {
        SimulatorService::stream_state(self, request).await
    }

    type StreamFramesStream = ResponseStream<pb::XrayFrame>;

    async fn stream_frames(
        &self,
        request: Request<pb::StreamFramesRequest>,
    ) -> Result<Response<Self::StreamFramesStream>, Status> {
        SimulatorService::stream_frames(self, request).await
    }

    type StreamMetricsStream = ResponseStream<pb::SessionUpdate>;

    async fn stream_metrics(
        &self,
        request: Request<pb::StreamMetricsRequest>,
    ) -> Result<Response<Self::StreamMetricsStream>, Status> {
        SimulatorService::stream_metrics(self, request).await
    }

    async fn get_anatomy(
        &self,
        request: Request<pb::GetAnatomyRequest>,
    ) -> Result<Response<pb::Anatomy>, Status> {
        SimulatorService::get_anatomy(self, request).await
    }

    async fn replay_session(
        &self,
        request: Request<pb::ReplaySessionRequest>,
    ) -> Result<Response<pb::ReplayResult>, Status> {
        SimulatorService::replay_session(self, request).await
    }

    async fn create_account(
        &self,
        request: Request<pb::CreateAccountRequest>,
    ) -> Result<Response<pb::Account>, Status> {
        SimulatorService::create_account(self, request).await
    }

    async fn list_accounts(
        &self,
        request: Request<pb::ListAccountsRequest>,
    ) -> Result<Response<pb::ListAccountsResponse>, Status> {
        SimulatorService::list_accounts(self, request).await
    }

    async fn who_am_i(
        &self,
        request: Request<pb::WhoAmIRequest>,
    ) -> Result<Response<pb::Account>, Status> {
        SimulatorService::who_am_i(self, request).await
    }

    async fn get_report(
        &self,
        request: Request<pb::GetReportRequest>,
    ) -> Result<Response<pb::Report>, Status> {
        SimulatorService::get_report(self, request).await
    }

    async fn get_report_frame(
        &self,
        request: Request<pb::GetReportFrameRequest>,
    ) -> Result<Response<pb::ReportFrame>, Status> {
        SimulatorService::get_report_frame(self, request).await
    }

    async fn get_history(
        &self,
        request: Request<pb::GetHistoryRequest>,
    ) -> Result<Response<pb::History>, Status> {
        SimulatorService::get_history(self, request).await
    }
}
