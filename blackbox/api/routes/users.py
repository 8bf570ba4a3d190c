"""The API's users (admin only): list and create them, change a role or a password, disable,
enable or delete one. Every change ends the tokens the user holds (credentials.change_user); an
admin may not disable, delete or demote their own account (409), so a black box always keeps the
admin who could undo it."""

from functools import partial
from typing import Annotated

from fastapi import APIRouter, Depends, HTTPException, Path, Response

from blackbox.api import credentials
from blackbox.api.credentials import USERNAME_RE, Claims
from blackbox.api.dependencies import ROLES_ADMIN, Services, allow
from blackbox.api.models import RoleChange, UserInfo, error_responses, new_user_model, password_change_model
from blackbox.register.store.record_store import User

UserName = Annotated[str, Path(pattern=USERNAME_RE.pattern, examples=["carol"], description="the user's name")]


def user_info(user: User) -> UserInfo:
    return UserInfo(name=user.name, role=user.role, created=user.created, disabled=user.disabled)


def not_yourself(admin: Claims, name: str, what: str) -> None:
    if admin.name == name:
        raise HTTPException(409, f"an admin may not {what} their own account: another admin can")


def build_router(services: Services) -> APIRouter:
    repo, accounts = services.repository, services.tokens.accounts

    def changed(user: User) -> UserInfo:
        """What a change answers; the accounts the API trusted are asked again from now on."""
        if accounts is not None:
            accounts.forget()
        return user_info(user)

    Admin = Annotated[Claims, Depends(allow(services.tokens, *ROLES_ADMIN))]
    min_password_length = services.settings.auth.min_password_length
    NewUserBody = new_user_model(min_password_length)
    PasswordBody = password_change_model(min_password_length)
    router = APIRouter(tags=["users"])
    on_a_user = error_responses(401, 404, 409, 413, 422, 503)

    @router.get("/users", response_model=list[UserInfo], responses=error_responses(401, 503))
    def list_users(_: Admin) -> list[UserInfo]:
        return [user_info(u) for u in repo.users()]

    @router.post(
        "/users", response_model=UserInfo, status_code=201, responses=error_responses(400, 401, 409, 413, 422, 503)
    )
    def create_user(new: NewUserBody, _: Admin) -> UserInfo:  # type: ignore[valid-type]
        return user_info(repo.add_user(services.passwords, new.name, new.role, new.password, min_password_length))

    @router.put("/users/{name}/role", response_model=UserInfo, responses=error_responses(400, 401, 404, 409, 422, 503))
    def change_role(name: UserName, body: RoleChange, admin: Admin) -> UserInfo:
        if body.role != "admin":
            not_yourself(admin, name, "demote")
        return changed(repo.change_user(partial(credentials.set_role, name=name, role=body.role)))

    @router.put(
        "/users/{name}/password", response_model=UserInfo, responses=error_responses(400, 401, 404, 413, 422, 503)
    )
    def change_password(name: UserName, body: PasswordBody, _: Admin) -> UserInfo:  # type: ignore[valid-type]
        change = partial(
            credentials.set_password,
            passwords=services.passwords,
            name=name,
            password=body.password,
            min_length=min_password_length,
        )
        return changed(repo.change_user(change))

    @router.post("/users/{name}/disable", response_model=UserInfo, responses=on_a_user)
    def disable_user(name: UserName, admin: Admin) -> UserInfo:
        not_yourself(admin, name, "disable")
        return changed(repo.change_user(partial(credentials.set_disabled, name=name, disabled=True)))

    @router.post("/users/{name}/enable", response_model=UserInfo, responses=error_responses(401, 404, 422, 503))
    def enable_user(name: UserName, _: Admin) -> UserInfo:
        return changed(repo.change_user(partial(credentials.set_disabled, name=name, disabled=False)))

    @router.delete("/users/{name}", status_code=204, response_class=Response, responses=on_a_user)
    def delete_user(name: UserName, admin: Admin) -> Response:
        not_yourself(admin, name, "delete")
        repo.delete_user(name)
        if accounts is not None:
            accounts.forget()
        return Response(status_code=204)

    return router
