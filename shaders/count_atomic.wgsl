// Frame counters without subgroup support: one atomic per invocation that has
// something to add. Call at the end of `main`, like the subgroup version.
fn count(c: u32, v: u32) {
    if v != 0u {
        atomicAdd(&counters[c], v);
    }
}
