//! Accounts: created by instructors (the token shown once, stored only as its hash), listed,
//! and the caller's own.

use cathlab_api::pb;
use tonic::{Request, Response, Status};

use super::state::SimulatorService;
use super::wire::{account_to_wire, peer_of, random_hex, unix_us};
use crate::reports::{AccountRole, Caller, store_status, token_hash};
use crate::store::StoredAccount;

impl SimulatorService {
    /// `CreateAccount` (instructors): a trainee's or an instructor's account and its token.
    pub(super) async fn create_account(
        &self,
        request: Request<pb::CreateAccountRequest>,
    ) -> Result<Response<pb::Account>, Status> {
        if !self.instructor(&request)? {
            return Err(Status::permission_denied(
                "creating accounts needs the instructor key or an instructor's account",
            ));
        }
        let r = request.into_inner();
        let name = r.name.trim();
        if name.is_empty() || name.len() > 100 {
            return Err(Status::invalid_argument("name: 1 to 100 bytes"));
        }
        let role = AccountRole::parse(&r.role)?;
        let token = random_hex(24);
        let account = StoredAccount {
            id: random_hex(8),
            name: name.to_owned(),
            role: role.as_str().to_owned(),
            token_hash: token_hash(&token),
            created_unix_s: unix_us() as f64 * 1e-6,
        };
        self.store.insert_account(&account).map_err(store_status)?;
        tracing::info!(account = %account.id, role = role.as_str(), "account created");
        Ok(Response::new(pb::Account {
            token,
            ..account_to_wire(&account)
        }))
    }

    /// `ListAccounts` (instructors): every account, oldest first.
    pub(super) async fn list_accounts(
        &self,
        request: Request<pb::ListAccountsRequest>,
    ) -> Result<Response<pb::ListAccountsResponse>, Status> {
        if !self.instructor(&request)? {
            return Err(Status::permission_denied(
                "listing accounts needs the instructor role",
            ));
        }
        let accounts = self.store.accounts().map_err(store_status)?;
        Ok(Response::new(pb::ListAccountsResponse {
            accounts: accounts.iter().map(account_to_wire).collect(),
        }))
    }

    /// `WhoAmI`: the account the token belongs to.
    pub(super) async fn who_am_i(
        &self,
        request: Request<pb::WhoAmIRequest>,
    ) -> Result<Response<pb::Account>, Status> {
        match self.caller(&request)? {
            Caller::Account(a) => Ok(Response::new(account_to_wire(&a))),
            Caller::InstructorKey => Ok(Response::new(pb::Account {
                name: "instructor (server key)".into(),
                role: AccountRole::Instructor.as_str().into(),
                ..pb::Account::default()
            })),
            Caller::Other(token) => {
                if token.is_some() {
                    self.throttle
                        .failed(peer_of(&request), "a token of no account");
                }
                Err(Status::unauthenticated("the token is not an account's"))
            }
        }
    }
}
