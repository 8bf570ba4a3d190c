// MongoDB's first start (docker-entrypoint-initdb.d, as root): the stack's own user `ares`,
// who reads and writes the black box's database (blackbox_store.mongo_db: ares) and nothing else:
// no other database, no users, no server administration. Root stays with the administrator.
const password = require("fs").readFileSync("/run/secrets/mongo_password", "utf8").trim();
db.getSiblingDB("admin").createUser({
  user: "ares",
  pwd: password,
  roles: [{ role: "readWrite", db: "ares" }],
});
