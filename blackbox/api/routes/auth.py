"""POST /auth/token (OAuth2 password form -> bearer token), POST /auth/renew (a valid token of
an account that still allows it -> a fresh one) and POST /auth/revoke (the token refused from then
on: a logout). Failed logins count towards the client's blacklisting."""

from typing import Annotated

from fastapi import APIRouter, Depends, Form, HTTPException, Request, Response

from blackbox.api.credentials import ROLES, Claims
from blackbox.api.dependencies import Services, allow
from blackbox.api.models import LoginForm, Token, error_responses


def build_router(services: Services) -> APIRouter:
    repo, tokens, passwords, guard = services.repository, services.tokens, services.passwords, services.guard
    Holder = Annotated[Claims, Depends(allow(tokens, *ROLES))]
    router = APIRouter(tags=["auth"])

    @router.post("/auth/token", response_model=Token, responses=error_responses(400, 401, 413, 422, 503))
    def token(request: Request, form: Annotated[LoginForm, Form()]) -> Token:
        ip = request.client.host if request.client else "unknown"

        def count_failure() -> None:
            verdict = guard.login_failed(ip)
            if verdict is not None:
                repo.record_blacklisting(ip, verdict.newly_blacklisted or "", guard.cfg.duration_s)

        # guesses spread over many addresses: the name's own limit (security.py), before any hashing
        locked = guard.account_locked(form.username)
        if locked is not None:
            count_failure()
            raise HTTPException(429, locked.detail, headers={"Retry-After": str(locked.retry_after_s)})
        user = repo.authenticate(passwords, form.username, form.password)
        if user is None:
            guard.account_failed(form.username)
            count_failure()
            raise HTTPException(401, "wrong user name or password", headers={"WWW-Authenticate": "Bearer"})
        access, ttl = tokens.issue(user.name, user.role, user.generation)
        return Token(access_token=access, expires_in=ttl, role=user.role)

    @router.post("/auth/renew", response_model=Token, responses=error_responses(401, 503))
    def renew(claims: Holder) -> Token:
        # the account was checked with the token (allow): the claims are the account as it is now
        access, ttl = tokens.issue(claims.name, claims.role, claims.generation)
        return Token(access_token=access, expires_in=ttl, role=claims.role)

    @router.post("/auth/revoke", status_code=204, response_class=Response, responses=error_responses(401, 503))
    def revoke(claims: Holder) -> Response:
        repo.revoke_token(claims)
        if tokens.accounts is not None:
            tokens.accounts.forget()  # it was trusted a moment ago: no longer
        return Response(status_code=204)

    return router
