"""GET /users and POST /users: the API's users (admin only)."""

from typing import Annotated

from fastapi import APIRouter, Depends

from blackbox.api.credentials import Claims
from blackbox.api.dependencies import ROLES_ADMIN, Services, allow
from blackbox.api.models import UserInfo, error_responses, new_user_model


def build_router(services: Services) -> APIRouter:
    repo = services.repository
    Admin = Annotated[Claims, Depends(allow(services.tokens, *ROLES_ADMIN))]
    min_password_length = services.settings.auth.min_password_length
    NewUserBody = new_user_model(min_password_length)
    router = APIRouter(tags=["users"])

    @router.get("/users", response_model=list[UserInfo], responses=error_responses(401, 503))
    def list_users(_: Admin) -> list[UserInfo]:
        return [UserInfo(name=u.name, role=u.role, created=u.created) for u in repo.users()]

    @router.post(
        "/users", response_model=UserInfo, status_code=201, responses=error_responses(400, 401, 409, 413, 422, 503)
    )
    def create_user(new: NewUserBody, _: Admin) -> UserInfo:  # type: ignore[valid-type]
        user = repo.add_user(services.passwords, new.name, new.role, new.password, min_password_length)
        return UserInfo(name=user.name, role=user.role, created=user.created)

    return router
