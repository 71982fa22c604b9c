// Frame counters, summed per subgroup: one atomic per subgroup, no workgroup barrier
// (llvmpipe runs barrier-free compute shaders as straight SIMD loops). Call from
// uniform control flow, i.e. at the end of `main`, by every invocation.
fn count(c: u32, v: u32) {
    let total = subgroupAdd(v);
    // The first active invocation (naga 30 has no subgroupElect).
    let first = subgroupExclusiveAdd(1u) == 0u;
    if first && total != 0u {
        atomicAdd(&counters[c], total);
    }
}
