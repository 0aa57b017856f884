// Run once by the mongo-init service of compose.cluster.yml (mongosh --file), against mongo-1.
// Makes mongo-1, mongo-2 and mongo-3 the replica set rs0, unless it is made already,
// then waits for a primary so that the servers, started after it, find one.
// tests/deploy/ (files.py) reads the set's name and members from this file.

const config = {
  _id: "rs0",
  members: [
    { _id: 0, host: "mongo-1:27017" },
    { _id: 1, host: "mongo-2:27017" },
    { _id: 2, host: "mongo-3:27017" },
  ],
};

function initiated() {
  try {
    return rs.status().ok === 1;
  } catch (e) {
    // NotYetInitialized (94) until rs.initiate has run; anything else is a real fault
    if (e.code === 94) {
      return false;
    }
    throw e;
  }
}

if (initiated()) {
  print("replica set " + config._id + " is made already");
} else {
  rs.initiate(config);
  print("replica set " + config._id + " initiated");
}

const deadline = Date.now() + 120 * 1000;
while (!db.hello().primary) {
  if (Date.now() > deadline) {
    throw new Error("no primary elected within 120 s");
  }
  sleep(1000);
}
print("primary: " + db.hello().primary);
