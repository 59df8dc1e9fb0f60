#!/usr/bin/env node
// Validate one .glb/.gltf with the Khronos glTF validator and print its JSON report.
// Usage: node validate_gltf.js FILE   (exit 0 when the report has no errors, 1 otherwise)
"use strict";
const fs = require("fs");
const path = require("path");
const validator = require("gltf-validator");

const file = process.argv[2];
if (!file) {
  console.error("usage: node validate_gltf.js FILE");
  process.exit(2);
}
const asset = fs.readFileSync(file);
validator
  .validateBytes(new Uint8Array(asset), {
    uri: path.basename(file),
    maxIssues: 0, // report every issue
    writeTimestamp: false,
  })
  .then((report) => {
    console.log(JSON.stringify(report, null, 2));
    process.exit(report.issues.numErrors > 0 ? 1 : 0);
  })
  .catch((error) => {
    console.error(String(error));
    process.exit(2);
  });
